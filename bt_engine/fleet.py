"""Several missions on one clock: the runner of a fleet.

Each mission keeps its own :class:`~bt_engine.runner.Runner` (its tree, blackboard, hooks,
tick log and watchdog); :class:`FleetRunner` steps them in lock-step on their shared clock:
every period each runner still running takes one step (the first moves the clock, the others
tick at the same time), then the fleet's own hooks run (e.g. a supervisor keeping the drones
apart). A runner whose mission ended is concluded at once (its tree halted, its drone
landed by its shutdown hooks) while the others go on. On a simulated clock the whole fleet
is deterministic; on a wall clock the runners share the real time.

SIGINT/SIGTERM stop every mission at the next step (a second one raises KeyboardInterrupt
in the shutdown hooks, as for one mission).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from bt_engine.interrupts import _restore_sigint, _route_signals, signal_source
from bt_engine.runner import Runner, RunResult


class FleetHook(Protocol):
    """Something that acts on the whole fleet after each step (any method may be missing)."""

    def after_step(self, t_s: float) -> None: ...


class FleetRunner:
    """Step ``runners`` (by name) in lock-step; see the module doc."""

    def __init__(self, runners: dict[str, Runner], hooks: list[Any] | None = None) -> None:
        if not runners:
            raise ValueError("a fleet needs at least one mission")
        periods = {round(r.period_s, 9) for r in runners.values()}
        if len(periods) != 1:
            raise ValueError("the missions of a fleet must tick at one rate")
        clocks = {id(r.clock) for r in runners.values()}
        if len(clocks) != 1:
            raise ValueError("the missions of a fleet must share one clock")
        self.runners = dict(runners)
        self.hooks = list(hooks or [])
        self.clock = next(iter(runners.values())).clock
        self._interrupts = 0
        #: called after every step with the runner (the CLI prints progress from it)
        self.on_step: Callable[[FleetRunner], None] | None = None

    def interrupt(self) -> None:
        """Stop every mission at the next step (what Ctrl-C does)."""
        self._interrupts += 1
        for r in self.runners.values():
            r.interrupt()

    @property
    def running(self) -> list[str]:
        """Names of the missions still running."""
        return [n for n, r in self.runners.items() if r.outcome is None]

    def run(self, max_time_s: float | None = None) -> dict[str, RunResult]:
        """Run every mission to its end; return each one's result by name."""

        def handler(signum, frame):  # noqa: ARG001
            source = signal_source(signum)
            for r in self.runners.values():
                r.interrupt_source = source
            self.interrupt()
            if self._interrupts >= 2:
                raise KeyboardInterrupt

        old = _route_signals(handler)
        concluded: set[str] = set()
        try:
            for r in self.runners.values():
                r.begin(max_time_s)
            while len(concluded) < len(self.runners):
                for name, r in self.runners.items():
                    if name not in concluded:
                        r.advance()
                t = self.clock.now()
                for hook in self.hooks:
                    fn = getattr(hook, "after_step", None)
                    if fn is not None:
                        fn(t)
                for name, r in self.runners.items():
                    if name not in concluded and r.outcome is not None:
                        concluded.add(name)
                        r.conclude()
                if self.on_step is not None:
                    self.on_step(self)
        finally:
            try:
                for name, r in self.runners.items():  # an exception above: land them all
                    if name not in concluded:
                        if r.outcome is None:
                            r.outcome = ("ABORTED", "the fleet run was stopped")
                        r.conclude()
            finally:
                _restore_sigint(old)
        return {name: r.result for name, r in self.runners.items() if r.result is not None}
